// The handloop API from the browser: bearer token (kept in localStorage, so every tab of this browser shares
// one sign-in; main.js follows a sign-in or sign-out made in another tab), JSON in and out, errors as ApiError
// with the server's `detail`, authorised blobs for images, server-sent events over fetch (EventSource cannot
// send the Authorization header).
export const TOKEN_KEY = "handloop.token";

/** @typedef {"annotate" | "review"} Queue  the two work queues (their routes differ only in this part) */

/** A query string from the parameters that are set (null, undefined and "" are left out). */
function query(/** @type {Record<string, string | number | null | undefined>} */ params) {
  const set = Object.entries(params).filter(([, v]) => v !== null && v !== undefined && v !== "");
  return set.length ? `?${new URLSearchParams(set.map(([k, v]) => [k, String(v)]))}` : "";
}

/**
 * The API's paths, one named function each: the only place in frontend/js that spells "/api/..." (a test,
 * tests/backend/api/test_frontend_paths.py, holds the other modules to that). Routes: backend/api/routes/.
 */
export const paths = Object.freeze({
  // accounts
  token: () => "/api/auth/token",
  me: () => "/api/auth/me",
  // the work queues (annotate and review)
  next: (/** @type {Queue} */ queue) => `/api/${queue}/next`,
  prefetch: (/** @type {Queue} */ queue) => `/api/${queue}/prefetch`,
  draft: (/** @type {Queue} */ queue, /** @type {number} */ sampleId) => `/api/${queue}/samples/${sampleId}/draft`,
  leaseRenew: (/** @type {Queue} */ queue, /** @type {number} */ sampleId) =>
    `/api/${queue}/samples/${sampleId}/lease/renew`,
  leaseRetake: (/** @type {Queue} */ queue, /** @type {number} */ sampleId) =>
    `/api/${queue}/samples/${sampleId}/lease/retake`,
  leaseRelease: (/** @type {Queue} */ queue, /** @type {number} */ sampleId) =>
    `/api/${queue}/samples/${sampleId}/lease/release`,
  activity: () => "/api/activity",
  // annotate
  proposals: (/** @type {number} */ sampleId) => `/api/annotate/samples/${sampleId}/proposals`,
  submissions: (/** @type {number} */ sampleId) => `/api/annotate/samples/${sampleId}/submissions`,
  skip: (/** @type {number} */ sampleId) => `/api/annotate/samples/${sampleId}/skip`,
  fitFailures: () => "/api/annotate/fit-failures",
  // review
  overlay: (/** @type {number} */ sampleId) => `/api/review/samples/${sampleId}/overlay`,
  decision: (/** @type {number} */ sampleId) => `/api/review/samples/${sampleId}/decision`,
  // guidelines
  guidelines: () => "/api/guidelines",
  guidelineImage: (/** @type {number} */ imageId) => `/api/guidelines/images/${imageId}`,
  adminGuidelines: () => "/api/admin/guidelines",
  adminGuidelineImages: () => "/api/admin/guidelines/images",
  adminGuidelineImage: (/** @type {number} */ imageId, /** @type {number} */ revision) =>
    `/api/admin/guidelines/images/${imageId}${query({ revision })}`,
  // admin: rounds, jobs, preannotation, people, data
  roundStatistics: () => "/api/admin/rounds/statistics",
  rounds: () => "/api/admin/rounds",
  roundCancel: (/** @type {number} */ roundId) => `/api/admin/rounds/${roundId}/cancel`,
  reviewQueue: () => "/api/admin/rounds/review-queue",
  dashboard: () => "/api/admin/dashboard",
  jobs: (/** @type {{kind?: string, limit?: number}} */ { kind, limit } = {}) => `/api/admin/jobs${query({ kind, limit })}`,
  jobCancel: (/** @type {number} */ jobId) => `/api/admin/jobs/${jobId}/cancel`,
  jobEvents: (/** @type {number} */ jobId) => `/api/admin/jobs/${jobId}/events`,
  preannotation: () => "/api/admin/preannotation",
  reliability: (/** @type {number} */ bins) => `/api/admin/reliability${query({ bins })}`,
  calibrationCheck: (/** @type {number} */ projectId) => `/api/admin/projects/${projectId}/calibration-check`,
  users: () => "/api/admin/users",
  user: (/** @type {number} */ userId) => `/api/admin/users/${userId}`,
  userLocks: () => "/api/admin/users/locks",
  unlockUser: (/** @type {number} */ userId) => `/api/admin/users/${userId}/unlock`,
  teamStatistics: () => "/api/admin/team/statistics",
  imports: () => "/api/admin/imports",
  datasetExport: (/** @type {string | number | null} */ upToRound = null) =>
    `/api/admin/exports/dataset${query({ up_to_round: upToRound })}`,
  samplesExport: () => "/api/admin/exports/samples",
  predictionsExport: () => "/api/admin/exports/predictions",
  freihandExport: () => "/api/admin/exports/freihand",
  freihandArchive: (/** @type {number} */ jobId) => `/api/admin/exports/freihand/${jobId}/archive`,
  // label quality (issue 40)
  quality: () => "/api/admin/quality",
  qualitySettings: () => "/api/admin/quality/settings",
  qualityGold: () => "/api/admin/quality/gold",
});

export class ApiError extends Error {
  constructor(status, detail) {
    super(detail || `HTTP ${status}`);
    this.status = status;
    this.detail = detail;
  }
}

export class Api {
  constructor(base = "") {
    this.base = base;
    this.token = localStorage.getItem(TOKEN_KEY);
    this.onunauthorized = null;
  }

  get signedIn() {
    return Boolean(this.token);
  }

  async login(email, password) {
    const form = new URLSearchParams({ username: email, password });
    const response = await fetch(`${this.base}${paths.token()}`, { method: "POST", body: form });
    if (!response.ok) throw new ApiError(response.status, await detailOf(response));
    const { access_token: token } = await response.json();
    this.token = token;
    localStorage.setItem(TOKEN_KEY, token);
    return token;
  }

  logout() {
    this.token = null;
    localStorage.removeItem(TOKEN_KEY);
  }

  // The token another tab stored (a sign-in there) or removed (a sign-out): taken over without writing.
  adopt(token) {
    this.token = token;
  }

  headers(extra = {}) {
    return this.token ? { Authorization: `Bearer ${this.token}`, ...extra } : extra;
  }

  /**
   * One request; throws ApiError unless the answer is 2xx. keepalive: the request outlives the page (a draft
   * saved while it unloads; bodies up to 64 KiB).
   * @param {string} method
   * @param {string} path  one of `paths` (above)
   * @param {{body?: any, signal?: AbortSignal, headers?: Record<string, string>, keepalive?: boolean}} [options]
   * @returns {Promise<Response>}
   */
  async fetch(method, path, { body, signal, headers, keepalive } = {}) {
    const init = { method, headers: this.headers(headers), signal, keepalive: Boolean(keepalive) };
    if (body instanceof FormData) {
      init.body = body; // multipart (a file upload): the browser writes its Content-Type with the boundary
    } else if (body !== undefined) {
      init.body = JSON.stringify(body);
      init.headers["Content-Type"] = "application/json";
    }
    const response = await fetch(`${this.base}${path}`, init);
    if (response.status === 401 && this.onunauthorized) this.onunauthorized(await detailOf(response.clone()));
    if (!response.ok) throw new ApiError(response.status, await detailOf(response));
    return response;
  }

  // JSON body, or null for 204.
  async json(method, path, body, options = {}) {
    const response = await this.fetch(method, path, { body, ...options });
    return response.status === 204 ? null : response.json();
  }

  get(path, options) {
    return this.json("GET", path, undefined, options);
  }

  post(path, body, options) {
    return this.json("POST", path, body, options);
  }

  put(path, body, options) {
    return this.json("PUT", path, body, options);
  }

  patch(path, body, options) {
    return this.json("PATCH", path, body, options);
  }

  async blob(path, options = {}) {
    return (await this.fetch("GET", path, options)).blob();
  }

  // Server-sent events: calls onEvent(name, data) until the stream ends or `signal` aborts.
  async events(path, onEvent, signal) {
    const response = await this.fetch("GET", path, { signal, headers: { Accept: "text/event-stream" } });
    const reader = response.body.getReader();
    const decoder = new TextDecoder();
    let buffer = "";
    for (;;) {
      const { value, done } = await reader.read();
      if (done) break;
      buffer += decoder.decode(value, { stream: true });
      let end;
      while ((end = buffer.indexOf("\n\n")) >= 0) {
        const block = buffer.slice(0, end);
        buffer = buffer.slice(end + 2);
        let name = "message", data = "";
        for (const line of block.split("\n")) {
          if (line.startsWith("event:")) name = line.slice(6).trim();
          else if (line.startsWith("data:")) data += line.slice(5).trim();
        }
        onEvent(name, data ? JSON.parse(data) : null);
      }
    }
  }
}

async function detailOf(response) {
  try {
    const body = await response.json();
    return typeof body.detail === "string" ? body.detail : JSON.stringify(body.detail);
  } catch {
    return `${response.status} ${response.statusText}`;
  }
}
