// Images and masks through the API (they need the bearer token, so no <img src>): fetched as blobs and
// decoded off the main thread with createImageBitmap; the browser's HTTP cache keeps them (ETag).
import { MaskLayer } from "./mask.js";

export async function loadBitmap(api, url) {
  return createImageBitmap(await api.blob(url));
}

export async function loadMask(api, url, width, height) {
  const bitmap = await loadBitmap(api, url);
  const canvas = new OffscreenCanvas(width, height);
  const ctx = canvas.getContext("2d", { willReadFrequently: true });
  ctx.drawImage(bitmap, 0, 0, width, height);
  bitmap.close();
  return MaskLayer.fromImageData(ctx.getImageData(0, 0, width, height));
}

// Every view's image (and mask, when the task has one) of a task.
export async function loadViews(api, task, { masks = true } = {}) {
  return Promise.all(task.views.map(async (view) => {
    const [image, mask] = await Promise.all([
      loadBitmap(api, view.image_url),
      masks && view.mask_url ? loadMask(api, view.mask_url, view.width, view.height) : Promise.resolve(null),
    ]);
    return { ...view, image, mask };
  }));
}
