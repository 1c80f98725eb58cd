// The documented REST API (openapi.yaml, base /api/v1), and nothing else: every request goes
// through `request`, which adds the bearer token, asks for one once when the server answers 401,
// and turns error bodies ({"error": {"code", "message"}}) into ApiError.

const BASE = '/api/v1';
const TOKEN_KEY = 'pathfarm-token';

export class ApiError extends Error {
  constructor(status, code, message) {
    super(message);
    this.status = status;
    this.code = code;
  }
}

export function token() {
  return localStorage.getItem(TOKEN_KEY);
}

export function forgetToken() {
  localStorage.removeItem(TOKEN_KEY);
}

// One prompt at a time: every request that gets a 401 while the dialog is open waits for the
// same answer, so the user is asked once, not once per poller. Resolves to the new token, or to
// null when a `dismissable` prompt is dismissed.
let pendingPrompt = null;

export function askToken(reason, { dismissable = false } = {}) {
  if (pendingPrompt) return pendingPrompt;
  const dialog = document.getElementById('token-dialog');
  const input = document.getElementById('token-input');
  document.getElementById('token-reason').textContent = reason;
  document.getElementById('token-dismiss').hidden = !dismissable;
  input.value = '';
  pendingPrompt = new Promise((resolve) => {
    const finish = (value) => {
      dialog.removeEventListener('close', onClose);
      pendingPrompt = null;
      resolve(value);
    };
    const onClose = () => {
      const t = input.value.trim();
      if (dialog.returnValue === 'save' && t) {
        localStorage.setItem(TOKEN_KEY, t);
        document.getElementById('token-change').hidden = false;
        finish(t);
      } else if (dismissable) {
        finish(null);
      } else {
        // Escape closes a modal dialog, but without a token nothing works: ask again.
        dialog.returnValue = '';
        dialog.showModal();
      }
    };
    dialog.addEventListener('close', onClose);
    dialog.returnValue = '';
    dialog.showModal();
    input.focus();
  });
  return pendingPrompt;
}

async function errorFrom(res) {
  let code = 'http_' + res.status;
  let message = `${res.status} ${res.statusText}`;
  try {
    const body = await res.json();
    if (body && body.error) {
      code = body.error.code;
      message = body.error.message;
    }
  } catch {
    // Not our JSON error body (a proxy, a 413 from the framework): keep the status line.
  }
  return new ApiError(res.status, code, message);
}

// fetch() with the token; resolves to the Response (2xx or 304), throws ApiError otherwise.
export async function request(path, { method = 'GET', body, headers, signal } = {}) {
  for (;;) {
    const h = new Headers(headers);
    const t = token();
    if (t) h.set('Authorization', `Bearer ${t}`);
    // no-store: the dashboard decides itself when to refetch (ETags); the HTTP cache must not
    // answer a poll with a stale body.
    const res = await fetch(BASE + path, { method, body, headers: h, signal, cache: 'no-store' });
    if (res.status === 401) {
      await askToken(t ? 'The saved token was refused. Enter a valid token.' : 'This server requires a token.');
      continue;
    }
    if (res.ok || res.status === 304) return res;
    throw await errorFrom(res);
  }
}

export async function getJson(path, opts) {
  const res = await request(path, opts);
  return res.json();
}

function sendJson(method, path, value) {
  return request(path, {
    method,
    body: value === undefined ? undefined : JSON.stringify(value),
    headers: value === undefined ? {} : { 'Content-Type': 'application/json' },
  });
}

export const api = {
  jobs: (state, page = 1, perPage = 50, signal) => {
    const q = new URLSearchParams({ page: String(page), per_page: String(perPage) });
    if (state) q.set('state', state);
    return getJson(`/jobs?${q}`, { signal });
  },
  job: (id, signal) => getJson(`/jobs/${encodeURIComponent(id)}`, { signal }),
  // A frame job's frame's history when `frame` is given, else the job's.
  convergence: (id, signal, frame = null) =>
    getJson(`/jobs/${encodeURIComponent(id)}/convergence${frame === null ? '' : `?frame=${frame}`}`, { signal }),
  // A page of workers: the first, or the one after cursor `after` (a page's `next`).
  workers: (after = null, perPage = 100, signal) => {
    const q = new URLSearchParams({ per_page: String(perPage) });
    if (after) q.set('after', after);
    return getJson(`/workers?${q}`, { signal });
  },
  cancel: (id) => sendJson('POST', `/jobs/${encodeURIComponent(id)}/cancel`).then((r) => r.json()),
  pause: (id) => sendJson('POST', `/jobs/${encodeURIComponent(id)}/pause`).then((r) => r.json()),
  resume: (id) => sendJson('POST', `/jobs/${encodeURIComponent(id)}/resume`).then((r) => r.json()),
  setPriority: (id, priority) =>
    sendJson('PATCH', `/jobs/${encodeURIComponent(id)}`, { priority }).then((r) => r.json()),
  remove: (id) => sendJson('DELETE', `/jobs/${encodeURIComponent(id)}`),
  submit: (sceneFile, settings, environmentFile) => {
    const form = new FormData();
    form.append('scene', sceneFile, sceneFile.name);
    form.append('settings', new Blob([JSON.stringify(settings)], { type: 'application/json' }));
    if (environmentFile) form.append('environment', environmentFile, environmentFile.name);
    return request('/jobs', { method: 'POST', body: form }).then((r) => r.json());
  },
};

// An image endpoint as a blob: <img src> cannot send the Authorization header, so images are
// fetched here and shown through object URLs. With `etag` (the last one seen) an unchanged image
// answers {changed: false} without a new blob.
export async function fetchImage(path, { etag, signal } = {}) {
  const headers = etag ? { 'If-None-Match': etag } : {};
  const res = await request(path, { headers, signal });
  const newTag = res.headers.get('ETag');
  if (res.status === 304 || (etag && newTag === etag)) {
    // A server that ignores If-None-Match still sends the body: drop it unread.
    if (res.body) res.body.cancel().catch(() => {});
    return { changed: false, etag };
  }
  const blob = await res.blob();
  return { changed: true, etag: newTag, blob, headers: res.headers };
}

// Saves an API file (EXR, PNG) under `filename`: fetch with the token, then a temporary
// <a download> on an object URL.
export async function download(path, filename) {
  const res = await request(path);
  const url = URL.createObjectURL(await res.blob());
  const a = document.createElement('a');
  a.href = url;
  a.download = filename;
  document.body.append(a);
  a.click();
  a.remove();
  // The click starts the download synchronously; give the browser a moment before revoking.
  setTimeout(() => URL.revokeObjectURL(url), 10_000);
}
