// The project's labelling guidelines (text and images an admin edits; GET /api/guidelines). On the annotate and
// review pages a "Guidelines" button in the top bar opens them in a panel at the side (it opens by itself after
// each change until the person closes it once, so a change reaches everyone); on the admin page a section edits them (PUT
// /api/admin/guidelines, images with a caption), each edit sent with the revision it was made on (409 when
// another admin saved meanwhile). The text is shown as text (paragraphs), never as HTML.
import { h, toast, fill } from "./dom.js";
import { paths } from "./api.js";

const SEEN_KEY = "handloop.guidelinesSeen.";

function paragraphs(text) {
  return text.split(/\n\s*\n/).filter((p) => p.trim()).map((p) => h("p", {}, p.split("\n").flatMap((line, i) =>
    i ? [h("br"), line] : [line])));
}

// The images' bytes need the bearer token: fetched as blobs, shown through object URLs.
async function imageUrls(api, images) {
  return Promise.all(images.map((i) => api.blob(paths.guidelineImage(i.id)).then((b) => URL.createObjectURL(b))));
}

function figures(images, urls) {
  return images.map((image, k) => h("figure", { class: "guideline-figure", dataset: { image: image.id } },
    h("img", { src: urls[k], alt: image.caption || "guideline image" }), image.caption ? h("figcaption", {}, image.caption) : null));
}

export function withGuidelines(mount) {
  return async (root, ctx) => {
    const page = await mount(root, ctx);
    const panel = new GuidelinesPanel(ctx.api, ctx.user);
    root.append(panel.aside);
    document.getElementById("nav")?.insertBefore(panel.button, document.querySelector("#nav .who"));
    panel.load().catch((error) => toast(`guidelines: ${error.message}`, "warn"));
    const unmount = page.unmount ? page.unmount.bind(page) : null;
    page.unmount = () => { panel.remove(); if (unmount) unmount(); };
    page.guidelines = panel;
    return page;
  };
}

export class GuidelinesPanel {
  constructor(api, user) {
    this.api = api;
    this.user = user;
    this.urls = [];
    this.body = h("div", { class: "guidelines-body" });
    this.aside = h("aside", { class: "guidelines-panel", hidden: true, "aria-label": "labelling guidelines" },
      h("div", { class: "guidelines-head" }, h("h2", {}, "Guidelines"),
        h("button", { class: "small close", "aria-label": "close the guidelines", onclick: () => this.close() }, "Close")),
      this.body);
    this.button = h("button", { class: "link guidelines-button", onclick: () => (this.aside.hidden ? this.show(true) : this.close()) },
      "Guidelines");
  }

  async load() {
    const g = await this.api.get(paths.guidelines());
    this.urls = await imageUrls(this.api, g.images);
    this.revision = g.revision;
    fill(this.body, g.revision === 0 && !g.text && !g.images.length
      ? h("p", { class: "muted" }, "No guidelines yet: an admin writes them on the admin page.")
      : [paragraphs(g.text), figures(g.images, this.urls)]);
    this.aside.dataset.revision = String(g.revision);
    // New to this person: open until they close it once (in any tab of this browser), then behind the button.
    if (g.revision > Number(localStorage.getItem(this.seenKey()) || 0)) this.show(true);
  }

  seenKey() {
    return SEEN_KEY + this.user.id;
  }

  close() {
    this.show(false);
    if (this.revision) localStorage.setItem(this.seenKey(), String(this.revision));
  }

  show(open) {
    this.aside.hidden = !open;
    this.button.classList.toggle("active", open);
  }

  remove() {
    this.aside.remove();
    this.button.remove();
    for (const url of this.urls) URL.revokeObjectURL(url);
  }
}

export function withGuidelinesEditor(mount) {
  return async (root, ctx) => {
    const page = await mount(root, ctx);
    const section = h("section", { class: "card wide", id: "guidelines-editor" });
    (root.querySelector(".admin-page") || root).append(section);
    const editor = new GuidelinesEditor(section, ctx.api);
    editor.load().catch((error) => fill(section, h("h2", {}, "Guidelines"), h("p", { class: "error" }, error.message)));
    return page;
  };
}

export class GuidelinesEditor {
  constructor(section, api) {
    this.section = section;
    this.api = api;
  }

  async load(g = null) {
    g = g || await this.api.get(paths.guidelines());
    this.revision = g.revision;
    const urls = await imageUrls(this.api, g.images);
    const text = h("textarea", { name: "guidelines-text", rows: 8, maxlength: 50000,
      placeholder: "How to label: which points count as occluded, when a view has no hand, …" });
    text.value = g.text;
    const file = h("input", { type: "file", name: "guidelines-image", accept: "image/png,image/jpeg,image/webp,image/gif" });
    const caption = h("input", { type: "text", name: "guidelines-caption", placeholder: "caption", maxlength: 500 });
    const save = async () => this.apply(() => this.api.put(paths.adminGuidelines(), { text: text.value, revision: this.revision }),
      "guidelines saved");
    const upload = async (e) => {
      e.preventDefault();
      if (!file.files.length) return toast("choose an image first", "warn");
      const form = new FormData();
      form.append("file", file.files[0]);
      form.append("caption", caption.value);
      form.append("revision", String(this.revision));
      await this.apply(async () => (await this.api.fetch("POST", paths.adminGuidelineImages(), { body: form })).json(),
        "image added");
    };
    fill(this.section, h("h2", {}, "Guidelines"),
      h("p", { class: "muted" }, "Shown on the annotate and review pages (after each change they open by themselves " +
        "until each person has closed them once). " +
        `Revision ${g.revision}. Blank lines separate paragraphs.`),
      text, h("div", { class: "button-row" }, h("button", { class: "primary save-guidelines", onclick: save }, "Save text")),
      h("div", { class: "guideline-images" }, g.images.map((image, k) => h("div", { class: "guideline-image" },
        figures([image], [urls[k]]), h("button", { class: "small danger", onclick: () => this.apply(() =>
          this.api.json("DELETE", paths.adminGuidelineImage(image.id, this.revision)), "image removed") },
        "Delete")))),
      h("form", { class: "inline-form guidelines-upload", onsubmit: upload }, file, caption,
        h("button", { type: "submit" }, "Add image")));
    this.section.dataset.revision = String(g.revision);
  }

  async apply(change, done) {
    try {
      const g = await change();
      toast(done, "ok", 2000);
      await this.load(g);
    } catch (error) {
      toast(`guidelines: ${error.message}`, "error", 10000);
    }
  }
}
