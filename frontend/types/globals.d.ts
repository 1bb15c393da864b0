// Types for `tsc --checkJs` only (no code): what the pages put on `window`. main.js sets `window.__handloop`
// (the API client, the page on screen, timing marks), which `bench ui` and the browser tests read.
interface Window {
  __handloop: { api: import("../js/api.js").Api; readonly page: any; marks: Record<string, number> };
}
