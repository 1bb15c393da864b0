// The single page: login, then a home per role (annotators annotate, reviewers review, admins see the
// dashboard), a hash route per page (#/annotate, #/review, #/admin).
import { Api, ApiError, paths, TOKEN_KEY } from "./api.js";
import { h, toast, fill } from "./dom.js";

const RANK = { annotator: 0, reviewer: 1, admin: 2 };
// The annotate and review pages with the guidelines' panel (guidelines.js); the admin page (admin.js) with the
// sections kept in their own modules added to it: team (statistics, unlock), FreiHAND export, guidelines' editor,
// calibration check, label quality.
const withGuidelines = (load) => () => Promise.all([load(), import("./guidelines.js")]).then(([m, g]) => g.withGuidelines(m));
const PAGES = {
  annotate: { label: "Annotate", role: "annotator",
    load: withGuidelines(() => import("./annotate.js").then((m) => m.mountAnnotate)) },
  review: { label: "Review", role: "reviewer", load: withGuidelines(() => import("./review.js").then((m) => m.mountReview)) },
  admin: { label: "Admin", role: "admin", load: () => Promise.all([import("./admin.js"), import("./admin_team.js"),
    import("./admin_freihand.js"), import("./guidelines.js"), import("./calibration_check.js"),
    import("./admin_quality.js")])
    .then(([admin, team, freihand, guide, check, quality]) => quality.withQuality(check.withCalibrationCheck(
      guide.withGuidelinesEditor(freihand.withFreihandExport(team.withTeam(admin.mountAdmin)))))) },
};
const HOME = { annotator: "annotate", reviewer: "review", admin: "admin" };

const api = new Api();
const app = document.getElementById("app");
const nav = document.getElementById("nav");
let user = null;
let page = null;

window.__handloop = { api, get page() { return page; }, marks: {} };

api.onunauthorized = (detail) => {
  if (!user) return;
  toast(`signed out: ${detail}`, "warn", 6000);
  signOut(false);
};

function allowed(name) {
  return user && RANK[user.role] >= RANK[PAGES[name].role];
}

// The look, per browser: a dark or light theme and a larger-target mode (bigger text, buttons, checkboxes and
// keys for touch screens or tired eyes), set on <html> as data-theme / data-targets (css/app.css).
const LOOK = { theme: ["handloop.theme", "dark", "light"], targets: ["handloop.targets", "normal", "large"] };

function applyLook() {
  for (const [name, [key, normal]] of Object.entries(LOOK)) {
    document.documentElement.dataset[name] = localStorage.getItem(key) || normal;
  }
}

function toggleLook(name) {
  const [key, a, b] = LOOK[name];
  localStorage.setItem(key, (localStorage.getItem(key) || a) === a ? b : a);
  applyLook();
  window.dispatchEvent(new Event("resize")); // canvases redraw at their new size
  const [theme, targets] = lookButtons(); // in place: the rest of the bar (a page's own buttons) stays
  nav.querySelector(".look-theme")?.replaceWith(theme);
  nav.querySelector(".look-targets")?.replaceWith(targets);
}

function lookButtons() {
  const light = document.documentElement.dataset.theme === "light";
  const large = document.documentElement.dataset.targets === "large";
  return [
    h("button", { class: "link look-theme", title: "switch between the dark and the light theme",
      "aria-pressed": String(light), onclick: () => toggleLook("theme") }, light ? "Dark theme" : "Light theme"),
    h("button", { class: `link look-targets${large ? " active" : ""}`, title: "bigger text, buttons and checkboxes",
      "aria-pressed": String(large), onclick: () => toggleLook("targets") }, large ? "Normal targets" : "Larger targets"),
  ];
}

function renderNav(current) {
  fill(nav, ...(user ? [
    ...Object.entries(PAGES).filter(([name]) => allowed(name)).map(([name, p]) =>
      h("a", { href: `#/${name}`, class: name === current ? "active" : "" }, p.label)),
    h("span", { class: "who" }, `${user.email} · ${user.role}`),
  ] : []), ...lookButtons(), user ? h("button", { class: "link", onclick: () => signOut(true) }, "Sign out") : null);
}

// Show a page: through the hash when it changes (hashchange routes), directly when it does not.
function go(name) {
  if (location.hash === `#/${name}`) route();
  else location.hash = `#/${name}`;
}

async function signOut(release) {
  if (page && release && page.releaseAll) await page.releaseAll().catch(() => null);
  unmountPage();
  api.logout();
  user = null;
  go("login");
}

function unmountPage() {
  if (page && page.unmount) page.unmount();
  page = null;
  fill(app, );
  delete document.body.dataset.ready;
}

function loginPage(message = "") {
  const email = h("input", { type: "email", name: "email", autocomplete: "username", required: true, autofocus: true });
  const password = h("input", { type: "password", name: "password", autocomplete: "current-password", required: true });
  const error = h("div", { class: "error", role: "alert" }, message);
  const submit = h("button", { class: "primary", type: "submit" }, "Sign in");
  const form = h("form", { class: "login", onsubmit: async (e) => {
    e.preventDefault();
    submit.disabled = true;
    error.textContent = "";
    try {
      await api.login(email.value, password.value);
      user = await api.get(paths.me());
      go(HOME[user.role]);
    } catch (err) {
      error.textContent = err instanceof ApiError ? err.detail : String(err);
      submit.disabled = false;
    }
  } },
  h("h1", {}, "handloop"),
  h("p", { class: "muted" }, "3D hand labeling: annotate, verify, bootstrap."),
  h("label", {}, "Email", email), h("label", {}, "Password", password), error, submit);
  fill(app, form);
  document.body.dataset.ready = "login";
  email.focus();
}

let routing = 0;

async function route() {
  const ticket = ++routing; // a newer route() call wins; an older one stops at its next await
  const name = location.hash.replace(/^#\/?/, "") || "";
  if (!user && api.signedIn) {
    try {
      user = await api.get(paths.me());
    } catch {
      api.logout();
    }
    if (ticket !== routing) return;
  }
  unmountPage();
  if (!user) {
    renderNav(null);
    return loginPage();
  }
  const target = PAGES[name] && allowed(name) ? name : HOME[user.role];
  if (target !== name) {
    history.replaceState(null, "", `#/${target}`);
  }
  renderNav(target);
  document.body.dataset.page = target;
  const mount = await PAGES[target].load();
  if (ticket !== routing) return;
  const root = h("div", { class: "page" });
  fill(app, root);
  try {
    const mounted = await mount(root, { api, user });
    if (ticket !== routing) return mounted.unmount();
    page = mounted;
    window.__handloop.marks[target] = performance.now();
  } catch (error) {
    root.append(h("div", { class: "error" }, `could not open ${target}: ${error.message}`));
    toast(`could not open ${target}: ${error.message}`, "error", 10000);
  }
}

// Start loading the page's module while the session is checked (its import is cached by the browser).
const wanted = location.hash.replace(/^#\/?/, "");
if (PAGES[wanted] && api.signedIn) PAGES[wanted].load().catch(() => null);

// Tabs share one sign-in (api.js keeps the token in localStorage): a sign-out in another tab signs this one out
// (its work in progress is kept like after a 401); a sign-in there as the same person only hands this tab the
// new token (its page carries on), as someone else it opens this tab's page for them.
window.addEventListener("storage", async (e) => {
  if (e.key !== TOKEN_KEY && e.key !== null) return;
  const token = localStorage.getItem(TOKEN_KEY);
  if (token === api.token) return;
  api.adopt(token);
  let who = null;
  if (token) {
    try {
      who = await api.get(paths.me());
    } catch {
      who = null;
    }
  }
  if (user && who && who.id === user.id) return;
  if (user) toast(who ? `signed in as ${who.email} in another tab` : "signed out in another tab", "warn", 6000);
  unmountPage();
  user = who;
  route();
});

// A Keys list (details.help on any page) opened by its key or its summary is scrolled to the top of its panel:
// it sits at the foot of a side panel and used to open below the fold (a list taller than the panel then
// shows from its first row on).
document.addEventListener("toggle", (e) => {
  const el = e.target;
  if (el instanceof HTMLDetailsElement && el.open && el.classList.contains("help")) {
    const box = el.getBoundingClientRect();
    if (box.bottom > window.innerHeight || box.top < 0) el.scrollIntoView({ block: "start" });
  }
}, true);

applyLook();
window.addEventListener("hashchange", route);
window.addEventListener("unhandledrejection", (e) => toast(`error: ${e.reason && e.reason.message ? e.reason.message : e.reason}`, "error", 8000));
route();
