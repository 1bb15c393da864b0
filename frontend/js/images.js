// Images and masks through the API (they need the bearer token, so no <img src>): fetched as blobs and
// decoded off the main thread with createImageBitmap; the browser's HTTP cache keeps them (ETag).
import { MaskLayer } from "./mask.js";

export async function loadBitmap(api, url) {
  return createImageBitmap(await api.blob(url));
}

// An automatic mask's bitmap -> MaskLayer (bits), on demand: decoding all views' masks up front cost
// ~10 ms per 1280x1024 view before the page could be used.
export function decodeMask(bitmap, width, height) {
  const canvas = new OffscreenCanvas(width, height);
  const ctx = canvas.getContext("2d", { willReadFrequently: true });
  ctx.drawImage(bitmap, 0, 0, width, height);
  return MaskLayer.fromImageData(ctx.getImageData(0, 0, width, height));
}

export async function loadMask(api, url, width, height) {
  const bitmap = await loadBitmap(api, url);
  const layer = decodeMask(bitmap, width, height);
  bitmap.close();
  return layer;
}

// One view's image and (when it has one) automatic mask bitmap, decoded off the main thread.
export async function loadView(api, view, { masks = true } = {}) {
  const [image, maskImage] = await Promise.all([
    loadBitmap(api, view.image_url),
    masks && view.mask_url ? loadBitmap(api, view.mask_url) : Promise.resolve(null),
  ]);
  return { image, maskImage };
}

// Every view of a task, loaded.
export async function loadViews(api, task, options = {}) {
  return Promise.all(task.views.map(async (view) => ({ ...view, ...(await loadView(api, view, options)) })));
}

// The full-resolution original of a view (its image_url serves the working-width copy where the project has
// a narrower working width): loaded when the annotator zooms past the copy's own pixels.
export async function loadFullImage(api, view) {
  const sep = view.image_url.includes("?") ? "&" : "?";
  return loadBitmap(api, `${view.image_url}${sep}full=true`);
}

// Whether a view drawn at `scale` screen px per full-resolution pixel (times devicePixelRatio) shows the
// working copy's pixels larger than a device pixel, so the full-resolution original would show more.
export function needsFullImage(view, scale, dpr = 1) {
  return Boolean(view.image) && view.image.width < view.width && scale * dpr * view.width / view.image.width > 1;
}
