// The handloop API from the browser: bearer token (kept in localStorage, so every tab of this browser shares
// one sign-in; main.js follows a sign-in or sign-out made in another tab), JSON in and out, errors as ApiError
// with the server's `detail`, authorised blobs for images, server-sent events over fetch (EventSource cannot
// send the Authorization header).
export const TOKEN_KEY = "handloop.token";

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
    const response = await fetch(`${this.base}/api/auth/token`, { method: "POST", body: form });
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

  // keepalive: the request outlives the page (a draft saved while it unloads; bodies up to 64 KiB).
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
